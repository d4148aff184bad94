#!/usr/bin/env python3
"""Where GICP started at the truth settles on the simulated families sets, per voxel grid and correspondence distance.

On simulated pairs the truth is exact, so how far small_gicp GICP moves from it is GICP's own error on those scans:
the grid's and the cost's, not the start's. For each ``--sims`` set (the scans of ``families.py``: the same seeds,
frames and cache) and each ``--grids`` entry ``VOXEL:CORR`` (m), GICP (the baseline's clouds and settings, one thread,
``preprocess.min_range`` as the pipeline has it for a plain cloud) from the truth of each neighbouring pair: its
rotation / translation error, and the axis of the rotation error in the target's world frame. ``--ideal`` simulates
the same frames again without motion within the sweep, range noise or dropouts (a simulator or motion effect then
goes; a grid effect stays). ``--finish ANGLE``: also the precision stage's GICP on ``registration.polish_voxel`` from
the truth, finished on each scan's scene-sized grid (``registration.polish_voxel_angle`` ANGLE: core/polish.py
``finish``). ::

    python scripts/benchmarks/gicp_truth.py --sims mid360:handheld:corridor mid360:legged:garage \\
        --grids 0.5:2.0 0.25:1.0 --finish 0.0625 --out results/gicp_truth
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)
import families  # noqa: E402


def ideal_frames(spec: str, picks_like: list) -> list:
    """The frames of a families set simulated again without motion in the sweep, range noise or dropouts."""
    from deepbbs_ros.sim.patterns import make_sensor
    from deepbbs_ros.sim.rig import make_simulator

    sensor, mount, place = spec.split(":")
    sim = make_simulator(place, families.sim_seed(spec), make_sensor(sensor, range_noise=0.0, dropout=0.0), mount,
                         frames=300, compensate=True, motion_distortion=False)
    picks = families.sim_picks(sim, mount, len(picks_like))
    return [(sim.scan_at(k).points.astype(np.float32), sim.pose_at(k)) for k in picks]


def from_truth(frames: list, voxel: float, corr: float) -> list[dict]:
    """GICP from the truth on each pair (k, k - 1) of ``frames`` [(points, T_world_lidar)]: errors and axis."""
    from scipy.spatial.transform import Rotation

    from deepbbs_ros.baselines import SmallGicpRegistration
    from deepbbs_ros.config import Config
    from deepbbs_ros.metrics import pair_errors

    g = SmallGicpRegistration("gicp", Config().replace(**{
        "eval.threads": 1, "eval.baseline_voxel_size": voxel, "eval.baseline_max_corr_dist": corr}))
    out = []
    for k in range(1, len(frames)):
        (src, Ts), (tgt, Tt) = frames[k], frames[k - 1]
        T = np.linalg.inv(Tt) @ Ts
        T_gicp = g.align(g.preprocess(src), g.preprocess(tgt), T).T_target_source
        rot, tr = pair_errors(T_gicp, T)
        rv = Tt[:3, :3] @ Rotation.from_matrix((T_gicp @ np.linalg.inv(T))[:3, :3]).as_rotvec()
        axis = rv / max(np.linalg.norm(rv), 1e-12)
        out.append({"pair": [k, k - 1], "rot_deg": float(rot), "trans_m": float(tr),
                    "axis_world": [round(float(a), 3) for a in axis]})
    return out


def finished_from_truth(frames: list, angle: float) -> list[dict]:
    """The precision stage from the truth on each pair (k, k - 1) of ``frames``: GICP on ``registration.polish_voxel``,
    then finished on the scans' grids at ``angle`` (rad) of their median ranges -> errors, and the finer grids (m)."""
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.polish import finish, polish, prepare_polish_cloud
    from deepbbs_ros.metrics import pair_errors

    cfg = Config().replace(**{"registration.polish_voxel_angle": angle, "registration.polish_threads": 1,
                              "registration.exact_gicp": True})
    rc, pp = cfg.registration, cfg.preprocess
    out = []
    for k in range(1, len(frames)):
        (src, Ts), (tgt, Tt) = frames[k], frames[k - 1]
        T = np.linalg.inv(Tt) @ Ts
        sc, tc = (prepare_polish_cloud(p, rc.polish_voxel, rc.polish_neighbors, min_range=pp.min_range,
                                       max_range=pp.max_range, threads=1, voxel_angle=angle) for p in (src, tgt))
        pol = polish(sc, tc, T, rc)
        fine = finish(sc, tc, pol.T_target_source, rc) if pol.applied else None
        T_end = fine.T_target_source if fine is not None and fine.applied else pol.T_target_source
        rot, tr = pair_errors(T_end, T)
        grids = [round(c.fine_voxel or rc.polish_voxel, 3) for c in (sc, tc)]
        out.append({"pair": [k, k - 1], "rot_deg": float(rot), "trans_m": float(tr), "grids_m": grids})
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sims", nargs="*", default=list(families.SIMS), help="simulated sets sensor:mount:place")
    p.add_argument("--sim-frames", type=int, default=5, help="scans per set (families.py --quick: 5)")
    p.add_argument("--grids", nargs="+", default=["0.5:2.0", "0.25:1.0"], help="VOXEL:CORR pairs (m)")
    p.add_argument("--ideal", action="store_true", help="also the frames simulated without motion, noise, dropouts")
    p.add_argument("--finish", type=float, default=0.0, metavar="ANGLE",
                   help="also GICP on polish_voxel finished on the scene's grid (registration.polish_voxel_angle)")
    p.add_argument("--cache", default="~/.cache/deepbbs_ros/bench", help="cache of the simulated scans")
    p.add_argument("--out", default="results/benchmarks", help="folder for gicp_truth.json")
    args = p.parse_args(argv)
    grids = [tuple(float(x) for x in g.split(":")) for g in args.grids]
    figures = {}
    for spec in args.sims:
        frames = families.sim_sets(argparse.Namespace(sims=[spec], sim_frames=args.sim_frames,
                                                      cache=args.cache)).popitem()[1]["frames"]
        variants = {"as simulated": frames}
        if args.ideal:
            variants["ideal"] = ideal_frames(spec, frames)
        for name, fr in variants.items():
            for voxel, corr in grids:
                rows = from_truth(fr, voxel, corr)
                figures[f"{spec}/{name}/{voxel}:{corr}"] = rows
                print(f"{spec} {name} grid {voxel} m, corr {corr} m: " + ", ".join(
                    f"{r['rot_deg']:.2f} deg / {r['trans_m']:.3f} m" for r in rows), flush=True)
            if args.finish > 0:
                rows = finished_from_truth(fr, args.finish)
                figures[f"{spec}/{name}/finish {args.finish}"] = rows
                print(f"{spec} {name} finished on the scene's grid ({args.finish} rad): " + ", ".join(
                    f"{r['rot_deg']:.2f} deg / {r['trans_m']:.3f} m ({r['grids_m'][0]} m)" for r in rows), flush=True)
    _common.write_json(Path(args.out), "gicp_truth.json", figures)
    return 0


if __name__ == "__main__":
    sys.exit(main())
