#!/usr/bin/env python3
"""Global localization in a prior map: MapLocalizer beside KISS-Matcher and FPFH + RANSAC, same queries, same run.

Data (generated once, cached as npz under ``--cache``; a rerun only measures):

* simulated, every scene type: a map of ``--map-length`` m of road (1 km) built from a first drive's scans at
  their ground-truth poses (one scan every ``--map-step`` m, cropped to ``--map-range`` m, voxel-downsampled to
  ``--map-voxel`` m); queries from second drives through the same world that never contributed to the map,
  spread evenly over it, in turn: driving back the other way in the opposite lane ("reverse"), in another lane of
  the same direction ("lane", 1.2-3.6 m over) and in the map drive's lane 0.4 m off its line ("same-lane"), each on
  another day (other parked cars, other traffic). Sweeps are
  compensated to their stamps. Highway and suburban drives get ``--repetitive`` extra queries on long
  straight stretches (away from curves and junctions): the repetitive places, reported apart.
* real (``--kitti``, ``--pair``): one pooled map of several places, each moved far from the others (``--spacing``
  m apart, a random yaw, fixed seed): the even scans of each KITTI sequence, and the target of the reference
  pair; the odd scans and the pair's source are the queries (a query must find its place as well as its pose).

Methods, from no initial guess (each query alone): ``maplocalizer`` (deepbbs_ros.core.localization.MapLocalizer,
built once per map with the map drive's keyframe poses; its verdict accepts or says why not);
``kiss-matcher+gicp`` (KISS-Matcher registering the scan against the whole map, then small_gicp GICP against
the whole map; accepted when KISS-Matcher says its solution is valid); ``fpfh-ransac+gicp`` (Open3D's
FPFH features and registration_ransac_based_on_feature_matching against the whole map, then GICP; Open3D has
no acceptance test: every answer counts as published). The baselines run on every ``--baseline-every``-th
query, each in a child process with a ``--baseline-timeout`` s limit (a timeout counts as no pose);
``--baseline-prior R`` gives them the map within R m of a coarse prior instead (context only).
``--grid-places``: MapLocalizer without the map drive's trajectory (candidate places over the map's drivable space);
``--outside N``: each map also answers N queries of another map (no pose is right, timed). Every method is
timed as a user runs it and every answer is the same on any machine and in every run: MapLocalizer is timed as
configured (GICP on every core) and answered by a twin that solves GICP on one thread (``registration.exact_gicp``;
its k-d trees and covariances, the same on any number of threads, use every core), whose own time is reported too
(``exact_time_s_*``); a baseline answers from a child process on one CPU (Open3D's RANSAC seeded) and is timed by a
second child on every core (``_localization_methods.ExactTimed``). ``--inexact``: the timed calls answer, one child per
baseline.

Figures (``localization.json`` under ``--out``), per method and map: share placed within 1 deg / 0.3 m (valid
and right), wrong poses accepted (valid but off), no pose (and how many of those "ambiguous"), timeouts, time per
query from no guess (the time to a first pose) p50 / p95, the same for the repetitive places, and how the time
grows with the map (the queries of the first ``--prefixes`` m against maps of those lengths). Each query is one
scan alone; the boot protocol (``boot`` in the figures, MapLocalizer only) is the node's case: a simulated query
with no pose goes on with the same drive's scans ``--boot-step`` s later (up to ``--boot-scans`` of them), each
searched once it has arrived and the search before it has ended, until one is placed or wrong; its time to the
first pose counts from the query scan's arrival. ``localization.png``
beside it: placed / wrong / no pose and the time p50 / p95 per map and method.

The parts, one job each: the data and its cache ``_localization_data.py``, the simulated maps ``_localization_sim.py``,
the methods as timed ``_localization_methods.py`` (the baselines' solvers ``_localization_baselines.py``), the
protocol ``_localization_eval.py``, the scores ``_localization_scores.py``, the table and the plot
``_localization_report.py``; this module parses the arguments and runs them.

    python scripts/benchmarks/localization.py --kitti PATH/TO/kitti/00 PATH/TO/kitti/02 --pair PATH/TO/pair \\
        --cache ~/.cache/deepbbs_ros/bench --out results/benchmarks
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)
from _localization_data import livox_map, real_map  # noqa: E402
from _localization_eval import evaluate_map, evaluate_outside  # noqa: E402
from _localization_methods import LABELS, METHODS  # noqa: E402
from _localization_report import plot, report  # noqa: E402
from _localization_scores import ROT_OK_DEG, TRANS_OK_M, aggregate  # noqa: E402
from _localization_sim import sim_map  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", nargs="*", default=["urban", "suburban", "highway", "open_road"],
                   help="simulated scene types, one 1 km map each")
    p.add_argument("--kitti", nargs="*", default=[], help="KITTI odometry sequence folders (velodyne/, poses.txt, "
                   "calib.txt) pooled into the real map, e.g. PATH/TO/kitti/00 PATH/TO/kitti/02")
    p.add_argument("--kitti-scans", type=int, default=10, help="the first scans of each KITTI sequence")
    p.add_argument("--pair", default=None, help="optional folder with a real pair: two .pcd files (target, source in "
                   "name order) and relative.txt (T_target_source); the target goes into the real map")
    p.add_argument("--livox", default=None, help="optional KITTI-layout folder of a handheld recording's keyframes: a "
                   "map of every other one at its pose, the others localized in it (a map of its own)")
    p.add_argument("--livox-every", type=int, default=8, help="with --livox: every n-th of the other keyframes is "
                   "a query")
    p.add_argument("--out", default="results/benchmarks", help="folder for localization.json")
    p.add_argument("--cache", default="~/.cache/deepbbs_ros/bench", help="cache of the generated maps and queries")
    p.add_argument("--methods", default=",".join(METHODS), help=f"comma list of {','.join(METHODS)}")
    p.add_argument("--queries", type=int, default=30, help="query scans per simulated scene, spread over the map")
    p.add_argument("--repetitive", type=int, default=6, help="extra queries on straight stretches (highway, "
                   "suburban)")
    p.add_argument("--map-length", type=float, default=1000.0, help="m of road per simulated map")
    p.add_argument("--map-step", type=float, default=2.5, help="m between the scans the map is built from")
    p.add_argument("--map-range", type=float, default=50.0, help="m, the map keeps each scan's points this close")
    p.add_argument("--map-voxel", type=float, default=0.2, help="m, voxel size of the map")
    p.add_argument("--prefixes", type=float, nargs="*", default=[250.0, 500.0], help="shorter maps (m) for the "
                   "time-versus-map-size figure")
    p.add_argument("--scaling-queries", type=int, default=4, help="queries per scene for the map-size figure")
    p.add_argument("--spacing", type=float, default=300.0, help="m between the real places in the pooled map")
    p.add_argument("--baseline-every", type=int, default=3, help="the baselines run on every n-th query")
    p.add_argument("--baseline-timeout", type=float, default=10.0, help="s per query and baseline")
    p.add_argument("--km-voxel", type=float, default=1.0, help="m, voxel of KISS-Matcher against the map")
    p.add_argument("--baseline-prior", type=float, default=0.0, help="m; > 0: the baselines register against the "
                   "map within this radius of a coarse prior (drawn within a quarter of it from the truth) instead "
                   "of the whole map; MapLocalizer never gets one")
    p.add_argument("--fpfh-voxel", type=float, default=1.0, help="m, voxel of the FPFH + RANSAC baseline")
    p.add_argument("--boot-scans", type=int, default=2, help="the boot protocol: a simulated query with no pose "
                   "goes on with up to this many later scans of its drive (0: single scans only)")
    p.add_argument("--boot-step", type=float, default=1.0, help="s between those scans (a search takes up to ~1 s; "
                   "the node takes the newest scan when it is free)")
    p.add_argument("--seed", type=int, default=1, help="seed of the real places' moves")
    p.add_argument("--sim-seed", type=int, default=None, help="world seed of the first scene (default: a held-out "
                   "test seed); the others follow")
    p.add_argument("--config", default=None, help="config YAML for MapLocalizer and the baselines")
    p.add_argument("--grid-places", action="store_true", help="MapLocalizer without the map drive's trajectory "
                   "(candidate places over the map's drivable space instead of keyframes)")
    p.add_argument("--inexact", action="store_true", help="the timed calls answer (MapLocalizer's GICP solve and "
                   "the baselines on every core): answers that can change from run to run (default: answered by "
                   "twins with registration.exact_gicp and baselines on one CPU, the same on any machine)")
    p.add_argument("--outside", type=int, default=0, help="also this many scans from places not in each map (the "
                   "next map's queries, spread over it; the last map gets the first's): no pose is right, "
                   "timed to the answer")
    p.add_argument("--outside-only", action="store_true", help="with --outside: measure only the scans outside")
    p.add_argument("--generate-only", action="store_true", help="build the cached maps and queries, measure nothing")
    p.add_argument("--quick", action="store_true", help="a smoke test: one scene, a 300 m map, 4 queries, no real "
                   "data unless given, baselines on 2 queries")
    args = p.parse_args(argv)
    if args.quick:
        args.scenes, args.map_length, args.queries, args.repetitive = args.scenes[:1], 300.0, 6, 0
        args.prefixes, args.scaling_queries, args.baseline_every = [150.0], 2, 2
    methods = [m for m in args.methods.split(",") if m]
    for m in methods:
        if m not in METHODS:
            raise SystemExit(f"unknown method {m!r} (known: {', '.join(METHODS)})")
    from deepbbs_ros.config import Config, load_config

    config = load_config(args.config) if args.config else Config()
    from deepbbs_ros.sim import SCENES
    from deepbbs_ros.train.cache import TEST_SEED_BASE

    base = TEST_SEED_BASE + 500 if args.sim_seed is None else args.sim_seed
    t_start = time.perf_counter()
    maps = {}
    for scene in args.scenes:
        maps[scene] = sim_map(scene, base + SCENES.index(scene), args)
    real = real_map(args)
    if real is not None:
        maps["real"] = real
    livox = livox_map(args)
    if livox is not None:
        maps["livox"] = livox
    t_gen = time.perf_counter() - t_start
    print(f"data ready in {t_gen:.0f} s: " + ", ".join(f"{k} {len(v.points)} pts / {len(v.queries)} queries"
                                                      for k, v in maps.items()))
    if args.generate_only:
        return 0
    figs = {}
    for name, data in maps.items():
        figs[name] = {"methods": {}, "rows": {}} if args.outside_only else evaluate_map(data, methods, args, config)
    if args.outside > 0 and len(maps) > 1:  # each map against another map's queries (every one out of it)
        names = list(maps)
        for i, name in enumerate(names):
            other = maps[names[(i + 1) % len(names)]].queries
            pick = np.unique(np.linspace(0, len(other) - 1, min(args.outside, len(other))).round().astype(int))
            figs[name]["outside"] = evaluate_outside(maps[name], [other[j] for j in pick], args, config)
            o = figs[name]["outside"]
            print(f"{name}: outside the map, {o.get('queries')} scans: no pose {100 * o.get('none_share', 0):.0f} %, "
                  f"wrong {o.get('wrong_count')}, p50 {o.get('time_s_p50', float('nan')):.2f} s, "
                  f"p95 {o.get('time_s_p95', float('nan')):.2f} s (CPU {o.get('cpu_s_p50', float('nan')):.2f} / "
                  f"{o.get('cpu_s_p95', float('nan')):.2f} s, load {os.getloadavg()[0]:.1f})")
    fig = {"maps": figs, "pooled": aggregate(figs, methods), "labels": LABELS,
           "tolerance": {"rot_deg": ROT_OK_DEG, "trans_m": TRANS_OK_M},
           "settings": {k: v for k, v in vars(args).items()},
           "data_s": t_gen, "measure_s": time.perf_counter() - t_start - t_gen}
    report(figs, methods)
    _common.write_json(Path(args.out), "localization.json", fig)
    plot(fig, Path(args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
