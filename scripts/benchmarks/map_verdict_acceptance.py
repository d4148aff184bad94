#!/usr/bin/env python3
"""The map verdict's acceptance on a real recording, apart from the search: a map of its every other keyframe at its
pose (with that trajectory's places), and per other keyframe (every ``--every``-th): GICP from the truth on the
nearest place's crop (right when within 1 degree / 0.3 m: should be accepted), and the truth moved 1 m / 2 degrees
and 2 m / 5 degrees in a random direction (wrong: should not). A pose is accepted as the localization accepts it: the
map verdict's probability at least ``localization.min_probability`` and, there, no second minimum as good along the
direction the fit leaves free (core/acceptance.py; ``--no-second-minimum``: the probability alone). Prints each query,
the counts and the check's time per pose it ran on. ::

    python scripts/benchmarks/map_verdict_acceptance.py PATH/TO/livox_avia_loop --every 2
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts" / "benchmarks"))

import localization as bench  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from deepbbs_ros.config import Config  # noqa: E402
from deepbbs_ros.core import acceptance, map_verdict  # noqa: E402
from deepbbs_ros.core.localization import MapLocalizer  # noqa: E402
from deepbbs_ros.core.polish import polish  # noqa: E402
from deepbbs_ros.metrics import pair_errors  # noqa: E402


def _moved(T: np.ndarray, metres: float, deg: float, rng: np.random.Generator) -> np.ndarray:
    ax, v = rng.normal(size=3), rng.normal(size=3)
    D = np.eye(4)
    D[:3, :3] = Rotation.from_rotvec(np.radians(deg) * ax / np.linalg.norm(ax)).as_matrix()
    D[:3, 3] = metres * v / np.linalg.norm(v)
    return T @ D


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folder", help="KITTI-layout folder of keyframes with poses.txt")
    ap.add_argument("--every", type=int, default=2, help="every n-th of the other keyframes is a query")
    ap.add_argument("--seed", type=int, default=0, help="seed of the moves' directions")
    ap.add_argument("--no-second-minimum", action="store_true", help="the map verdict's probability alone")
    args = ap.parse_args(argv)
    data = bench.livox_map(SimpleNamespace(livox=args.folder, livox_every=args.every, map_range=50.0, map_voxel=0.2))
    cfg = Config().replace(**{"localization.second_minimum": not args.no_second_minimum})
    loc = MapLocalizer(data.points, cfg, trajectory=data.trajectory)
    rng = np.random.default_rng(args.seed)
    right = rejected = wrong = accepted = 0
    ms: list[float] = []

    def judge(prep, crop, T: np.ndarray) -> tuple[float, bool, str]:
        p = map_verdict.answer_probability(prep.pre, crop, T, cfg)
        if not acceptance.accepts(cfg, p):
            return p, False, ""
        t = time.perf_counter()
        amb = acceptance.second_minimum(prep.pre, crop, T, cfg)
        if cfg.localization.second_minimum:
            ms.append((time.perf_counter() - t) * 1e3)
        what = f" (free {amb.uncertainty:.1f} tol, other minimum {amb.offset:.1f} tol)" if amb.ambiguous else ""
        return p, not amb.ambiguous, what

    for i, q in enumerate(data.queries):
        prep, T = loc.prepare(q.points), q.T_map_scan
        crop = loc._crop(int(np.argmin(np.linalg.norm(loc.places[:, :2, 3] - T[:2, 3], axis=1))))
        pol = polish(prep.pre.polish_cloud.complete(), crop.pre.polish_cloud.complete(),
                     np.linalg.inv(crop.T_map_place) @ T, cfg.registration)
        T_gicp = crop.T_map_place @ pol.T_target_source if pol.applied else T
        rot, trans = pair_errors(T_gicp, T)
        p, ok, why = judge(prep, crop, T_gicp)
        if rot < 1.0 and trans < 0.3:
            right += 1
            rejected += int(not ok)
        moved = [judge(prep, crop, _moved(T, m, g, rng)) for m, g in ((1, 2), (2, 5))]
        wrong += len(moved)
        accepted += sum(int(ok_m) for _, ok_m, _ in moved)
        print(f"{i}: GICP from the truth {rot:.2f} deg {trans:.2f} m, p {p:.3f}{'' if ok else ' rejected'}{why}; "
              + ", ".join(f"moved {name} p {pm:.3f}{' accepted' if ok_m else ''}{w}"
                          for name, (pm, ok_m, w) in zip(("1 m / 2 deg", "2 m / 5 deg"), moved)), flush=True)
    print(f"right {right}, rejected {rejected}; wrong {wrong}, accepted {accepted}")
    if ms:
        print(f"second-minimum check on {len(ms)} poses: p50 {np.median(ms):.1f} ms, "
              f"p95 {np.percentile(ms, 95):.1f} ms")
    loc.registration.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
