#!/usr/bin/env python3
"""Sim-to-real sanity check on a real LiDAR scan pair (not part of the repository's data).

The pair lives outside the project (``../shared/realdata/hdl32_pair``: two real HDL-32E scans,
``251370668.pcd`` = target, ``251371071.pcd`` = source, ``relative.txt`` = the reference
``T_target_source`` from fast_gicp's tests, itself a registration good to about 1-3 cm / 0.2-0.4 deg).
Each trial moves the source by a known random yaw (up to ``--yaw-deg``) and horizontal shift (up to
``--shift`` m), registers it with DeepBBS++ (and GICP from identity for comparison), undoes the known
motion and compares with the reference:

    T_perturbed = P @ ... : source points p' = P p, so T_target_source = T_est(p') @ P

Usage::

    python scripts/realdata_check.py [--pair ../shared/realdata/hdl32_pair] [--trials 6] [--weights W]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from deepbbs_ros.baselines import SmallGicpRegistration
from deepbbs_ros.config import Config
from deepbbs_ros.core.registration import DeepBBSRegistration
from deepbbs_ros.datasets.pcd import read_pcd_points
from deepbbs_ros.errors import DeepBBSError
from deepbbs_ros.metrics import pair_errors
from deepbbs_ros.train.pairs import make_T, yaw_matrix


def _xyz(path: Path) -> np.ndarray:
    return read_pcd_points(path)[0].astype(np.float64)


def main(argv: list[str] | None = None) -> int:
    here = Path(__file__).resolve().parent.parent
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--pair", type=Path, default=here.parent / "shared" / "realdata" / "hdl32_pair")
    p.add_argument("--source", default="251371071.pcd")
    p.add_argument("--target", default="251370668.pcd")
    p.add_argument("--trials", type=int, default=6)
    p.add_argument("--yaw-deg", type=float, default=45.0)
    p.add_argument("--shift", type=float, default=5.0, help="m")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--weights", default="", help="checkpoint ('' = the shipped model)")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)
    try:
        src = _xyz(args.pair / args.source)
        tgt = _xyz(args.pair / args.target)
        T_ref = np.loadtxt(args.pair / "relative.txt").reshape(4, 4)
        cfg = Config()
        cfg.registration.threads = args.threads
        reg = DeepBBSRegistration(cfg, weights=args.weights)
        gicp = SmallGicpRegistration("gicp", cfg)
    except (DeepBBSError, OSError, ValueError) as err:
        print(f"realdata_check: {err}", file=sys.stderr)
        return 1
    rng = np.random.default_rng(args.seed)
    print(f"{args.pair}: source {len(src)} pts, target {len(tgt)} pts, weights {reg.weights_path}")
    print(f"{'trial':>5} {'yaw deg':>8} {'shift m':>8} | {'DeepBBS++ rot':>13} {'trans':>7} {'ms':>6} | "
          f"{'GICP rot':>9} {'trans':>7}")
    ok = {"deepbbs++": 0, "gicp": 0}
    for k in range(args.trials):
        yaw = np.deg2rad(rng.uniform(-args.yaw_deg, args.yaw_deg))
        ang = rng.uniform(0, 2 * np.pi)
        r = args.shift * np.sqrt(rng.uniform())
        P = make_T(yaw_matrix(yaw), np.array([r * np.cos(ang), r * np.sin(ang), 0.0]))
        src_p = src @ P[:3, :3].T + P[:3, 3]
        t0 = time.perf_counter()
        T_d = reg.register(src_p, tgt).T_target_source @ P
        ms = 1e3 * (time.perf_counter() - t0)
        T_g = gicp.register(src_p, tgt).T_target_source @ P
        rd, td = (float(e) for e in pair_errors(T_d, T_ref))
        rg, tg = (float(e) for e in pair_errors(T_g, T_ref))
        ok["deepbbs++"] += rd <= 1.0 and td <= 0.3
        ok["gicp"] += rg <= 1.0 and tg <= 0.3
        print(f"{k:>5} {np.rad2deg(yaw):>8.1f} {r:>8.2f} | {rd:>13.3f} {td:>7.3f} {ms:>6.0f} | {rg:>9.3f} {tg:>7.3f}")
    print(f"within 1 deg / 0.3 m of the reference: DeepBBS++ {ok['deepbbs++']}/{args.trials}, "
          f"GICP from identity {ok['gicp']}/{args.trials}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
