#!/usr/bin/env python3
"""Does a smaller ``localization.rank_shortlist`` rank the same candidates? For every query of the localization
benchmark's cached maps (``localization.py --cache``; the map without its trajectory) and 8 scans of the next map, the
candidates (places, descriptor distances, yaws, centres) ranked with every place against those ranked with each
shortlist, and the ranking's CPU ms per query.

    python scripts/benchmarks/rank_shortlist.py --cache PATH/TO/cache --kitti PATH/TO/kitti/00 PATH/TO/kitti/02 \\
        PATH/TO/nuscenes_hdl32 --pair PATH/TO/hdl32_pair --sizes 500 1000 2000
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402,F401  (puts the checkout first on sys.path)
import localization as bench  # noqa: E402
import search_profile  # noqa: E402


def _key(ranked) -> list:
    return [(p, round(d, 9), round(y, 9), tuple(np.round(c, 9))) for p, d, y, c in ranked]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cache", required=True)
    p.add_argument("--scenes", nargs="*", default=["urban", "highway", "suburban", "open_road"])
    p.add_argument("--kitti", nargs="*", default=[])
    p.add_argument("--pair", default=None)
    p.add_argument("--sizes", type=int, nargs="+", default=[500, 1000, 2000])
    args = p.parse_args(argv)
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.localization import MapLocalizer
    from deepbbs_ros.core.registration import DeepBBSRegistration

    cfg = Config().replace(**{"registration.network_process": "off"})
    reg = DeepBBSRegistration(cfg)
    maps = {s: search_profile._cached(Path(args.cache).expanduser(), s) for s in args.scenes}
    if args.kitti or args.pair:
        maps["real"] = bench.real_map(argparse.Namespace(kitti=args.kitti, kitti_scans=40, pair=args.pair, seed=1,
                                                         spacing=300.0, map_range=50.0, map_voxel=0.2))
    names = list(maps)
    for i, name in enumerate(names):
        loc = MapLocalizer(maps[name].points, cfg, registration=reg)
        other = maps[names[(i + 1) % len(names)]].queries
        pick = np.unique(np.linspace(0, len(other) - 1, 8).round().astype(int))
        scans = [q.points for q in maps[name].queries] + [other[j].points for j in pick]
        same, cpu = dict.fromkeys(args.sizes, 0), dict.fromkeys([0, *args.sizes], 0.0)
        centres = loc.description_centres
        for pts in scans:
            desc = loc.describe(pts, centres)
            got = {}
            for n in [0, *args.sizes]:
                loc.config = cfg.replace(**{"localization.rank_shortlist": n})
                t = time.process_time()
                got[n] = _key(loc.rank(desc, None, centres))
                cpu[n] += time.process_time() - t
            for n in args.sizes:
                same[n] += got[n] == got[0]
        print(f"{name}: {len(loc.places)} places, {len(scans)} scans; the same candidates as with every place: "
              + ", ".join(f"shortlist {n}: {same[n]}" for n in args.sizes) + "; rank CPU ms per scan: "
              + ", ".join(f"{n or 'all'} {1e3 * v / len(scans):.0f}" for n, v in cpu.items()), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
