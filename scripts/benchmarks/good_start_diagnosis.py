#!/usr/bin/env python3
"""Why the verdict rejects a pose: per pair of a families.py simulated set, each verdict stage printed.

For each pair of the set (``families.py --quick``'s pairs and starts: the good start, and with ``--basin`` the basin
offsets) and each pose judged (the truth; GICP from the start; that pose finished on the scene-sized grids, judged on
GICP's grid, on the scene's and on both, core/finish_verdict.py; with ``--pipeline`` the full pipeline's answer): its
error, the calibrated probability (``good_start`` coefficients) with the features whose log-odds terms pull it down
most, ``pinned`` and the weakest direction (a twist in tolerances: 0.3 m, 1 degree) with its uncertainty, and the
second-minimum check (core/second_minimum.py: the minima its starts found, tolerances away, fitness). The skew check
needs per-point times, which the simulated sets do not keep (compensated sweeps).

    python scripts/benchmarks/good_start_diagnosis.py --sim mid360:handheld:corridor
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402,F401  (puts the checkout first on sys.path)
import families  # noqa: E402
import registration as _reg  # noqa: E402


def stages(name: str, pts, T, T_gt, spc, tgt, rc, dist: float | None = None, second: bool = True) -> None:
    """Print the verdict's stages of the pose ``T`` (4, 4) judged from ``pts`` against ``tgt`` at ``dist``."""
    from deepbbs_ros.core import anchoring, calibrated, second_minimum, visibility
    from deepbbs_ros.metrics import pair_errors

    d = rc.verdict_dist if dist is None else dist
    f = visibility.pose_features(pts, T, tgt, d, 1, True, True)
    coef, icpt = calibrated.load()["good_start"]
    terms = sorted(zip(visibility.FEATURES, coef * calibrated.design(f)[0]), key=lambda t: t[1])[:3]
    twist, unc = second_minimum.weakest(pts @ T[:3, :3].T + T[:3, 3], tgt, d)
    rot, trans = pair_errors(T, T_gt)
    print(f"  {name}: {rot:.2f} deg / {trans:.2f} m, probability {calibrated.probability(f, 'good_start'):.3f}; "
          + ", ".join(f"{n} {v:.3f}" for n, v in zip(visibility.FEATURES, f) if n in (
              "fitness", "consistency", "violations_nb", "pinned", "anchored_far")))
    print("     lowest log-odds terms " + ", ".join(f"{n} {v:+.1f}" for n, v in terms)
          + ("" if twist is None else f"; weakest direction {np.round(twist / anchoring.SCALE, 2).tolist()}, "
             f"free by {unc:.1f} tolerances"))
    if second:
        amb = second_minimum.check(pts, T, spc, tgt, rc)
        print(f"     second minimum: ambiguous {amb.ambiguous}, minima (tolerances, fitness) "
              f"{[(round(float(a), 1), round(float(b), 3)) for a, b in amb.found]}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--sim", default="mid360:handheld:corridor", help="a families.py simulated set sensor:mount:place")
    p.add_argument("--basin", action="store_true", help="also the basin offsets' starts (the truth and the pipeline)")
    p.add_argument("--pipeline", action="store_true", help="also the full pipeline's answer (register())")
    p.add_argument("--seed", type=int, default=1, help="families.py's --seed (the basin offsets' signs)")
    p.add_argument("--cache", default="~/.cache/deepbbs_ros/bench", help="cache of the simulated scans")
    args = p.parse_args(argv)

    from deepbbs_ros.config import Config
    from deepbbs_ros.core import finish_verdict, verdict
    from deepbbs_ros.core.good_start import from_start, good_start_points
    from deepbbs_ros.core.polish import finish
    from deepbbs_ros.core.registration import DeepBBSRegistration

    ns = argparse.Namespace(sims=[args.sim], sim_frames=5, cache=str(Path(args.cache).expanduser()), pairs_per_set=8,
                            basin_pairs=2, pair_trials=1, seed=args.seed)  # families.py --quick's
    sets = families.sim_sets(ns)
    cfg = Config().replace(**{"registration.exact_gicp": True})
    reg, rc = DeepBBSRegistration(cfg), cfg.registration
    try:
        for c in families.plan(sets, ns):
            if c["level"] and not args.basin:
                continue
            frames = sets[c["set"]]["frames"]
            P = _reg.yaw_shift(*c["move"])
            src = (frames[c["i"]][0] @ P[:3, :3].T + P[:3, 3]).astype(np.float32)
            T_gt = np.linalg.inv(frames[c["j"]][1]) @ frames[c["i"]][1] @ np.linalg.inv(P)
            print(f"scan {c['i']} to {c['j']}, start moved {np.round(c['move'], 2).tolist()} (yaw deg, x, y m)")
            spc, tpc = (reg.preprocess(x, lazy=True).polish_cloud.complete(1) for x in (src, frames[c["j"]][0]))
            pts = good_start_points(spc, rc)
            stages("truth", pts, T_gt, T_gt, spc, tpc, rc)
            if args.pipeline:
                res = reg.register(src, frames[c["j"]][0])
                stages(f"pipeline (valid {res.valid})", pts, res.T_target_source, T_gt, spc, tpc, rc)
            if c["level"]:
                continue
            pol = from_start(spc, tpc, np.eye(4), rc)
            if not pol.applied:
                print(f"  GICP from the start: {pol.reason}")
                continue
            stages("GICP from the start", pts, pol.T_target_source, T_gt, spc, tpc, rc)
            fine = finish(spc, tpc, pol.T_target_source, rc)
            if fine is None or not fine.applied:
                continue
            stages("finished, on GICP's grid", pts, fine.T_target_source, T_gt, spc, tpc, rc)
            scene = verdict.on_scene_grid(spc, tpc, rc)
            stages("finished, on the scene's grids", scene[0], fine.T_target_source, T_gt, spc, scene[1], rc,
                   scene[2], second=False)
            prob, why = finish_verdict.judge(pts, fine.T_target_source, spc, tpc, rc, rc.good_start_probability)
            print(f"     on both grids: probability {prob:.3f}, {'taken' if not why else why}")
    finally:
        reg.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
