#!/usr/bin/env python3
"""The skew check end to end: ``register()`` on raw simulated Livox sweeps with their per-point times, check on and off.

For each ``--rigs`` entry ``SENSOR:MOUNT:PLACE`` the simulator (``--seed``; rig ``i`` records with seed ``seed * 100 +
i``) records raw sweeps (the motion skew kept, per-point times); on ``--pairs`` pairs 1, 3 or 6 frames apart each scan
is prepared once with its times (as the node does) and registered twice by the same prepared scans: the whole
pipeline from identity and the good start from the truth moved a little (within 3 degrees / 0.5 m), with
``registration.skew_check`` off and on. Per rig and way: right (1 deg / 0.3 m) and wrong (beyond 2 deg / 0.5 m)
answers, accepted (``valid``) or rejected, off and on; and the check's CPU per accepted pose (``core.sweep_skew.check``
timed again on the answer, one thread) over the good start's GICP (the same pair, from the same start). ::

    python scripts/benchmarks/sweep_skew.py --rigs mid360:legged:hall avia:handheld:hall --seed 39 --pairs 6 \\
        --out results/sweep_skew
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402,F401  (puts the checkout first on sys.path)
import numpy as np  # noqa: E402

GAPS = (1, 3, 6)


def _label(T: np.ndarray, T_gt: np.ndarray) -> str:
    from deepbbs_ros.metrics import pair_errors

    r, t = (float(x) for x in pair_errors(T, T_gt))
    return "right" if r <= 1.0 and t <= 0.3 else "wrong" if r > 2.0 or t > 0.5 else "between"


def rig_figures(spec: str, index: int, seed: int, pairs: int) -> dict:
    from deepbbs_ros.config import Config
    from deepbbs_ros.core import sweep_skew
    from deepbbs_ros.core.good_start import from_start
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.sim.rig import make_simulator

    sensor, mount, place = spec.split(":")
    sim = make_simulator(place, seed * 100 + index, sensor, mount, frames=40, compensate=False)
    base = {"registration.threads": 1, "registration.polish_threads": 1, "registration.network_process": "off"}
    regs = {on: DeepBBSRegistration(Config().replace(**base, **{"registration.skew_check": on}))
            for on in (False, True)}
    rc, rng = regs[True].config.registration, np.random.default_rng([seed, index])
    counts = {way: {f"{c}_{a}_{on}": 0 for c in ("right", "between", "wrong") for a in ("accepted", "rejected")
                    for on in ("off", "on")} for way in ("pipeline", "good_start")}
    cost = []
    for k in range(pairs):
        i = int(rng.integers(0, 40 - 7))
        j = i + GAPS[k % len(GAPS)]
        tgt_s, src_s = sim.scan_at(i), sim.scan_at(j)
        T_gt = np.linalg.inv(tgt_s.T_world_lidar) @ src_s.T_world_lidar
        yaw, shift = np.radians(rng.uniform(-3, 3)), rng.uniform(-0.5, 0.5, 2)
        T0 = T_gt.copy()
        T0[:2, :2] = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]) @ T_gt[:2, :2]
        T0[:2, 3] += shift
        src = regs[True].preprocess(src_s.points, src_s.point_times(), src_s.stamp_ns)
        tgt = regs[True].preprocess(tgt_s.points, tgt_s.point_times(), tgt_s.stamp_ns)
        for way, kw in (("pipeline", {}), ("good_start", {"T_init": T0, "good_start": True})):
            for on in (False, True):
                res = regs[on].register(src, tgt, preprocessed=True, **kw)
                c = _label(res.T_target_source, T_gt)
                counts[way][f"{c}_{'accepted' if res.valid else 'rejected'}_{'on' if on else 'off'}"] += 1
                if on and way == "good_start" and res.skew:  # the check ran: its CPU against the good start's GICP
                    t0 = time.process_time()
                    sweep_skew.check(src, tgt, res.T_target_source, rc, regs[on].config.preprocess.min_range)
                    t1 = time.process_time()
                    from_start(src.polish_cloud, tgt.polish_cloud, T0, rc)
                    cost.append((t1 - t0, time.process_time() - t1))
    c = np.array(cost).reshape(-1, 2)
    out = {"counts": counts, "check_ms": round(1e3 * float(np.median(c[:, 0])), 2) if len(c) else None,
           "check_over_gicp": round(float(np.median(c[:, 0] / c[:, 1])), 2) if len(c) else None}
    for reg in regs.values():
        reg.close()
    print(spec, out, flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rigs", nargs="+", default=["mid360:legged:hall", "avia:handheld:hall"],
                    metavar="SENSOR:MOUNT:PLACE")
    ap.add_argument("--seed", type=int, default=39)
    ap.add_argument("--pairs", type=int, default=6, help="pairs per rig (default 6)")
    ap.add_argument("--out", type=Path, default=Path("results/benchmarks"))
    args = ap.parse_args(argv)
    figures = {spec: rig_figures(spec, i, args.seed, args.pairs) for i, spec in enumerate(args.rigs)}
    _common.write_json(args.out, "sweep_skew.json", figures)
    return 0


if __name__ == "__main__":
    sys.exit(main())
